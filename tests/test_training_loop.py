"""The one resumable loop (``recondreamer.training_loop.run_steps``) and its progress lines."""

from __future__ import annotations

import logging

import pytest

from recondreamer.training_loop import ProgressLog, format_duration, run_steps


def _run(start: int, total: int, checkpoint_every: int, log_every: int, caplog):
    calls: list[tuple[str, int]] = []
    progress = ProgressLog("job", total, start, log_every)

    def step(before: int) -> dict[str, float]:
        calls.append(("step", before))
        return {"loss": float(before), "psnr": 20.0 + before}

    with caplog.at_level(logging.INFO, logger="recondreamer.training_loop"):
        run_steps(progress, step, start, total, checkpoint_every, lambda done: calls.append(("save", done)),
                  lambda done: calls.append(("after", done)))
    return calls, progress, [r.getMessage() for r in caplog.records]


class TestRunSteps:
    def test_each_step_then_its_hook_then_a_checkpoint_every_k_steps_short_of_the_last(self, caplog):
        calls, _, _ = _run(0, 6, 2, 10, caplog)
        assert calls == [
            ("step", 0), ("after", 1), ("step", 1), ("after", 2), ("save", 2), ("step", 2), ("after", 3),
            ("step", 3), ("after", 4), ("save", 4), ("step", 4), ("after", 5), ("step", 5), ("after", 6),
        ]

    def test_a_resumed_job_takes_only_the_steps_left(self, caplog):
        calls, _, _ = _run(4, 6, 2, 10, caplog)
        assert [c for c in calls if c[0] == "step"] == [("step", 4), ("step", 5)]
        assert ("save", 4) not in calls and ("save", 6) not in calls

    def test_a_finished_job_takes_no_step(self, caplog):
        calls, _, lines = _run(6, 6, 2, 1, caplog)
        assert calls == [] and lines == []


class TestProgressLog:
    def test_logs_the_window_means_every_k_steps_and_at_the_last(self, caplog):
        _, progress, lines = _run(0, 5, 100, 2, caplog)
        assert [line.split(" loss ")[0] for line in lines] == ["job step 2/5", "job step 4/5", "job step 5/5"]
        assert " loss 0.50000 " in lines[0] and " loss 2.50000 " in lines[1] and " loss 4.00000 " in lines[2]
        assert all("ms/step" in line and "CPU ms/step" in line and " ETA " in line for line in lines)
        assert progress.last_mean == {"loss": 4.0, "psnr": 24.0}

    def test_a_job_describes_its_own_fields(self, caplog):
        progress = ProgressLog("recon", 2, 0, 1, describe=lambda mean: f"psnr {mean['psnr']:.1f}")
        with caplog.at_level(logging.INFO, logger="recondreamer.training_loop"):
            progress.update(1, {"loss": 1.0, "psnr": 21.25})
        assert "recon step 1/2 loss 1.00000 psnr 21.2 " in caplog.records[0].getMessage()


@pytest.mark.parametrize("seconds, text", [(0, "0m00s"), (59.6, "1m00s"), (61, "1m01s"), (3600, "1h00m00s"), (7325, "2h02m05s")])
def test_format_duration(seconds, text):
    assert format_duration(seconds) == text
