"""Regenerate the model bundled for `fogd --demo` (fogd/data/demo-model.json).

Simulates the heating and cooling calibration runs the README's quick start uses and trains fogd's default
method on them with the paper's PSO settings, exactly as `fogd-train` does:

    python tools/make_demo_model.py          # about a minute on 2 cores
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from accuracy_table import CALIBRATION, simulated_run  # noqa: E402

from fogd.calibration.models import FitOptions  # noqa: E402
from fogd.calibration.training import TrainConfig, train  # noqa: E402
from fogd.core import modelfile  # noqa: E402

OUTPUT = Path(__file__).resolve().parent.parent / "fogd" / "data" / "demo-model.json"


def main() -> None:
    runs = [simulated_run(name, 1 + i, 50.0) for i, name in enumerate(CALIBRATION)]
    config = TrainConfig(name="fogd-demo (simulated FOG, paper-train + cooling)", fit=FitOptions(n_jobs=2))
    trained = train(runs, config)
    modelfile.save(OUTPUT, trained.document)
    print(f"wrote {OUTPUT}: {trained.fitted.hyperparameters}, held-out RMSE {trained.fitted.cv_rmse_dph:.3e} deg/h")


if __name__ == "__main__":
    main()
