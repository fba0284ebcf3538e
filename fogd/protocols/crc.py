"""The two CRCs fogd's wire formats use: CRC-32/MPEG-2 (KVH frames) and CRC-16/CCITT-FALSE (fogd frames).

Both run in C through `binascii`'s table-driven CRCs: CRC-16/CCITT-FALSE is `crc_hqx` seeded with 0xFFFF,
and CRC-32/MPEG-2 is the bit mirror of zlib's reflected CRC-32 (mirror every input byte with a 256-entry
table, run zlib's CRC with its final XOR undone, mirror the 32-bit register back). A Python loop over a
256-entry table costs about ten times as much per KVH frame.
"""

import binascii

MIRRORED_BYTES = bytes(int(f"{value:08b}"[::-1], 2) for value in range(256))


def crc32_mpeg2(data: bytes | bytearray) -> int:
    """CRC-32/MPEG-2: poly 0x04C11DB7, init 0xFFFFFFFF, no reflection, no final XOR."""
    reflected = binascii.crc32(data.translate(MIRRORED_BYTES)) ^ 0xFFFFFFFF
    return int.from_bytes(reflected.to_bytes(4, "little").translate(MIRRORED_BYTES), "big")


def crc32_mpeg2_ok(frame: bytes | bytearray) -> bool:
    """True when `frame` ends with the big-endian CRC-32/MPEG-2 of the bytes before it (the CRC over all is 0)."""
    # The mirrored register is 0 exactly when the MPEG-2 register is 0; no need to mirror it back.
    return binascii.crc32(frame.translate(MIRRORED_BYTES)) == 0xFFFFFFFF


def crc16_ccitt_false(data: bytes | bytearray) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final XOR."""
    return binascii.crc_hqx(data, 0xFFFF)


def crc16_ccitt_false_ok(frame: bytes | bytearray) -> bool:
    """True when `frame` ends with the big-endian CRC-16/CCITT-FALSE of the bytes before it."""
    return binascii.crc_hqx(frame, 0xFFFF) == 0
