"""A run's wall-clock stamps and progress bars: per iteration from a ``jax.debug.callback``
(``Progress.hook``), or spread over the slices of ``run`` when no callback is compiled in."""

from __future__ import annotations

import threading
import time
from typing import Any

from ptrl_jax.config import ExperimentConfig


class Progress:
    """Wall-clock stamps per iteration, and with ``show`` a tqdm bar per stage.

    With ``show``, a ``jax.debug.callback`` stamps every iteration of every vmapped run as it
    ends. Without it the program holds no host callback at all (so XLA's persistent cache can
    keep it) and the stamps come from the slice boundaries of ``run`` instead, spread evenly over
    the iterations of each slice (exact when ``checkpoint_every`` is 1)."""

    def __init__(self, cfg: ExperimentConfig, show: bool):
        n_targets = len(cfg.variants) * cfg.seeds * len(cfg.targets)
        self.n_targets = n_targets
        self.totals = {
            "source": cfg.source_iterations,
            "target": cfg.target.ppo.num_iterations * n_targets,
        }
        self.steps_per_call = {
            "source": cfg.source.ppo.env_steps_per_iteration,
            "target": cfg.target.ppo.env_steps_per_iteration,
        }
        self.show = show
        self.lock = threading.Lock()
        self.times: dict[tuple[str, int, int], float] = {}
        self.stage_start: dict[str, float] = {}
        self.counts = {"source": 0, "target": 0}
        self.spread_over = 0
        """Most iterations one call ran whose stamps ``record_slice`` had to spread (0: every
        stamp was measured by the callback or covers one iteration)."""
        self.bars: dict[str, Any] = {}
        self.t0 = time.monotonic()

    def start(self) -> None:
        # On resume, wall times continue from the last saved stamp (the downtime is not counted).
        last = max(self.times.values(), default=0.0)
        self.t0 = time.monotonic() - last

    def restore(self, meta: dict) -> None:
        """Wall-clock stamps and progress counts saved with a resume state."""
        self.times = {(s, int(r), int(i)): float(t) for s, r, i, t in meta.get("times", [])}
        self.stage_start = {k: float(v) for k, v in meta.get("stage_start", {}).items()}
        for (stage, _, _) in self.times:
            self.counts[stage] += 1

    def record_slice(self, before: tuple[int, int], after: tuple[int, int], t_start: float) -> None:
        """Stamp the (source, target) iterations a slice ran, where no callback did."""
        t_end = time.monotonic() - self.t0
        done = [("source", i) for i in range(before[0] + 1, after[0] + 1)]
        done += [("target", i) for i in range(before[1] + 1, after[1] + 1)]
        if any((stage, 0, it) not in self.times for stage, it in done):
            self.spread_over = max(self.spread_over, len(done))
        for k, (stage, it) in enumerate(done):
            t = t_start + (t_end - t_start) * (k + 1) / len(done)
            runs = range(self.n_targets) if stage == "target" else (0,)
            if stage == "target" and "target" not in self.stage_start:
                self.stage_start["target"] = self.last_time_before("target")
            self.stage_start.setdefault("source", 0.0)
            for r in runs:
                self.times.setdefault((stage, r, it), t)

    def hook(self, stage: str):
        if not self.show:
            return None

        def callback(d: dict) -> None:
            now = time.monotonic() - self.t0
            with self.lock:
                self.times[(stage, int(d["run_id"]), int(d["iteration"]))] = now
                if stage not in self.stage_start:
                    self.stage_start[stage] = self.last_time_before(stage)
                self.counts[stage] += 1
                if self.show:
                    self._update_bar(stage, now, float(d["episode_reward"]))

        return callback

    def last_time_before(self, stage: str) -> float:
        # The target stage starts when the source's last iteration ends (at 0 when the source
        # comes from a checkpoint and has no iterations).
        if stage == "target":
            return max((t for (s, _, _), t in self.times.items() if s == "source"), default=0.0)
        return 0.0

    def _update_bar(self, stage: str, now: float, reward: float) -> None:
        from tqdm import tqdm

        if stage not in self.bars:
            for bar in self.bars.values():
                bar.close()
            self.bars[stage] = tqdm(total=self.totals[stage], initial=self.counts[stage] - 1, desc=f"{stage:>6}",
                                    unit="it", dynamic_ncols=True)
        bar = self.bars[stage]
        bar.update(1)
        elapsed = max(now - self.stage_start[stage], 1e-9)
        sps = self.counts[stage] * self.steps_per_call[stage] / elapsed
        bar.set_postfix_str(f"{sps:,.0f} env steps/s, reward {reward:.3f}")
        if self.counts[stage] >= self.totals[stage]:
            bar.close()

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()


def interpolated_times_note(slice_iterations: int) -> str:
    """Report note for runs without the progress callback: ``Progress.record_slice`` then stamps
    each iteration of a call at an even share of the call's time, source and target alike, so
    the per-stage wall times (and wall time to threshold) are estimates, not measurements."""
    return (f"Progress was off: wall times are spread evenly over the iterations of each call (up to "
            f"{slice_iterations} iterations, source and target alike), so stage wall times and wall "
            f"time to threshold are estimates within a call; env steps are exact")
