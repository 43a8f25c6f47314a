"""The notebooks in experiments/notebooks run at smoke scale, and are committed without outputs.

Each notebook's code cells are executed in order in this process, with the cell tagged
``parameters`` followed by the test's values (papermill's convention): an nbmake equivalent that
lets the notebooks reuse the smoke program that tests/test_end_to_end.py compiles in the same
xdist worker (``ptrl_jax.run`` keeps compiled programs per process), so each costs seconds.
"""

import json
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from ptrl_jax.io import artifacts

pytestmark = pytest.mark.xdist_group("smoke_go2_to_xbot")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "experiments" / "notebooks"


def execute(path: Path, parameters: dict) -> dict:
    matplotlib.use("Agg")
    notebook = json.loads(path.read_text())
    namespace: dict = {"__name__": "__main__"}
    for index, cell in enumerate(notebook["cells"]):
        if cell["cell_type"] != "code":
            continue
        code = compile("".join(cell["source"]), f"{path.name}[cell {index}]", "exec")
        exec(code, namespace)
        if "parameters" in cell.get("metadata", {}).get("tags", []):
            namespace.update(parameters)
    return namespace


class TestCommittedNotebooks:
    @pytest.mark.parametrize("name", ["freeze_ratio_ablation.ipynb", "transfer_table.ipynb"])
    def test_outputs_are_stripped(self, name):
        notebook = json.loads((NOTEBOOKS / name).read_text())
        code = [c for c in notebook["cells"] if c["cell_type"] == "code"]
        assert code and all(c["outputs"] == [] and c["execution_count"] is None for c in code)
        assert sum("parameters" in c["metadata"].get("tags", []) for c in code) == 1


class TestFreezeRatioNotebook:
    def test_runs_the_sweep_and_plots_reward_against_rho(self, tmp_path):
        ns = execute(NOTEBOOKS / "freeze_ratio_ablation.ipynb", {"RUNS_DIR": tmp_path})
        assert [p["rho"] for p in ns["points"]] == [0.0, 0.25, 0.5, 0.75, 1.0]  # presets fill the ends
        assert ns["run_dir"].parent.parent == tmp_path
        # The notebook's points are the run's report: the rho = 0.5 row against metrics.csv.
        rows = artifacts.read_metrics_csv(ns["run_dir"] / "metrics.csv")
        half = next(p for p in ns["points"] if p["rho"] == 0.5)
        final = [np.mean([r["episode_reward"] for r in rows if r["preset"] == "rho0.5" and r["seed"] == s][-10:])
                 for s in range(2)]
        assert half["final_reward_mean"] == pytest.approx(np.mean(final), abs=1e-5)


class TestTransferTableNotebook:
    def test_runs_the_experiment_and_builds_its_table_row(self, tmp_path):
        ns = execute(NOTEBOOKS / "transfer_table.ipynb", {"RUNS_DIR": tmp_path})
        (row,) = ns["rows"]
        assert (row["source"], row["target"], row["transfer_preset"], row["seeds"]) == ("go2", "xbot_l", "L2", 2)
        assert set(ns["curves"]) == {"none", "L1", "L2", "L1+L2", "scratch", "rho0.25", "rho0.5", "rho0.75",
                                     "none@semantic", "L2@semantic"}

    def test_shows_a_finished_batch_without_running(self, tmp_path, capsys):
        (tmp_path / "table4.md").write_text("# Table IV: stand-in\n")
        ns = execute(NOTEBOOKS / "transfer_table.ipynb", {"BATCH_DIR": str(tmp_path)})
        assert "result" not in ns and "Table IV: stand-in" in capsys.readouterr().out
