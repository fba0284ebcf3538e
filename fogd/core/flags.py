"""Per-sample status flags that travel with every compensated sample (CSV `flags`, fogd frames)."""

from enum import IntFlag


class Flag(IntFlag):
    """Bits of the `flags` column; 0 means a normal, fully compensated sample."""

    WARMUP = 1  # rate-estimator window not yet full: temperature rate taken as 0
    CLAMPED = 2  # a model input was outside the calibrated domain and was clamped
    TEMP_STALE = 4  # no fresh temperature within the configured time: the last one is held
    RATE_INVALID = 8  # the gyro rate is NaN/Inf or its status bit says invalid: not compensated
    TEMP_INVALID = 16  # the temperature is NaN or out of range: the last valid one is held
    OUT_OF_DOMAIN = 32  # the inputs together are far from any calibration data (joint-space guard)
    WARMING = 64  # cold start: the inputs rest on the equilibrium assumption beyond its tolerance (fogd.core.warming)


def describe(flags: int) -> str:
    """Names of the set bits, e.g. 'WARMUP|CLAMPED', or 'OK'."""
    names = [flag.name for flag in Flag if flags & flag and flag.name]
    return "|".join(names) if names else "OK"
