"""Regenerate the model bundled for `fogd --demo` (fogd/data/demo-model.json).

Simulates the calibration runs of tools/accuracy_table.py (heating, cooling, a cycle) with a navigation-grade
gyro, the one `fogd --demo` emulates, at the demo's sample rate, and trains pso-svr on fogd's default inputs (the
lag bank, the ladder's top rung) with the paper's PSO settings, as `fogd-train --method pso-svr` does:

    python tools/make_demo_model.py          # a few minutes on 2 cores
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from accuracy_table import CALIBRATION, simulated_run  # noqa: E402

from fogd.calibration.models import FitOptions  # noqa: E402
from fogd.cli.demo import NOISE, RATE_HZ  # noqa: E402
from fogd.calibration.training import TrainConfig, train  # noqa: E402
from fogd.core import modelfile  # noqa: E402
from fogd.simulation.simulator import params_for  # noqa: E402

OUTPUT = Path(__file__).resolve().parent.parent / "fogd" / "data" / "demo-model.json"


def main() -> None:
    params = params_for(NOISE)
    runs = [simulated_run(name, 1 + i, RATE_HZ, params) for i, name in enumerate(CALIBRATION)]
    config = TrainConfig(name=f"fogd-demo (simulated navigation-grade FOG, {' + '.join(CALIBRATION)})",
                         fit=FitOptions(n_jobs=2))  # fmt: skip
    trained = train(runs, config)
    modelfile.save(OUTPUT, trained.document)
    print(f"wrote {OUTPUT}: {trained.fitted.hyperparameters}, held-out RMSE {trained.fitted.cv_rmse_dph:.3e} deg/h")


if __name__ == "__main__":
    main()
