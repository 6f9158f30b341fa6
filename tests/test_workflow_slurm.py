"""End to end on SLURM: the quick experiment (the same config as ``quick_experiment``) submitted job
by job with sbatch by snakemake-executor-plugin-slurm to the single-node test cluster
(.test/slurm/start.sh: Debian's slurm-wlm and munge), through profiles/slurm as written plus
.test/slurm/profile for that cluster. Every job of the DAG must go through sbatch, with the
partition, GPU and memory requests of profiles/slurm; one job, cancelled with scancel while it
runs, must be resubmitted by the profile's retries; and the five tables must equal those of the
local run to the last digit (same seeds, same single-threaded commands, nothing timed in them).

System tier (``pytest -m system``): the test uses a running cluster (in $RECONDREAMER_SLURM_DIR,
else /tmp/recondreamer-slurm) and never starts or installs one; .ci/run starts it. Without one it
fails, naming the command that starts it."""

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import pandas as pd
import pytest
import yaml

from workflow_fixtures import EXPERIMENT_CONFIGS, QUICK_WEIGHTS, copy_workflow

SLURM_PROFILE = ("--workflow-profile", "profiles/slurm", "--profile", ".test/slurm/profile")
CLUSTER_DIR = Path(os.environ.get("RECONDREAMER_SLURM_DIR") or "/tmp/recondreamer-slurm")
START_COMMAND = ".test/slurm/start.sh"  # root; .ci/run runs it
CANCELLED_RULE = "train_recondreamer"  # the quick DAG's longest jobs (about 9 CPU s after the job's parses)
CANCEL_AFTER_S = 5  # running time before the cancel: past the job's two workflow parses, inside its command


@pytest.fixture(scope="session")  # session: checked before the session's quick run is built, so a missing cluster fails at once
def slurm_cluster():
    """The running test cluster's folder and the environment that points SLURM's commands at it."""
    where = f"{CLUSTER_DIR} ($RECONDREAMER_SLURM_DIR)"
    if shutil.which("scontrol") is None:
        pytest.fail(f"SLURM's commands are not installed: `apt-get install slurm-wlm munge`, then `{START_COMMAND}` (.ci/run does both)")
    conf = CLUSTER_DIR / "slurm.conf"
    if not conf.is_file():
        pytest.fail(f"no test SLURM cluster in {where}: start one with `{START_COMMAND}` (as root; .ci/run does)")
    # bin/ holds an srun bound to this cluster's slurm.conf: the plugin's job step drops SLURM_CONF.
    env = {**os.environ, "SLURM_CONF": str(conf), "PATH": f"{CLUSTER_DIR / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    ping = subprocess.run(["scontrol", "ping"], capture_output=True, text=True, env=env, timeout=60)
    if " is UP" not in ping.stdout:
        pytest.fail(f"the test SLURM cluster in {where} does not answer ({(ping.stdout + ping.stderr).strip()}): "
                    f"start it with `{START_COMMAND}` (as root; .ci/run does)")
    return CLUSTER_DIR, env


def dag_job_counts(log: str) -> Counter:
    """Jobs per rule of the DAG, from the first 'Job stats:' table Snakemake prints."""
    lines = log[log.index("Job stats:"):].splitlines()[3:]  # after the title, the header and the rule
    counts = Counter()
    for line in lines:
        rule, count = line.split()
        if rule == "total":
            assert sum(counts.values()) == int(count), lines
            return counts
        counts[rule] = int(count)
    raise AssertionError(f"no total line in the job stats: {lines}")


def slurm_jobs(run_id: str, env: dict, states: str = "all") -> list[dict]:
    """The jobs SLURM holds for this run (finished ones stay for an hour: MinJobAge in start.sh)."""
    fields = ("JobID", "State", "Partition", "tres-per-job", "MinMemory", "NumCPUs", "Comment", "TimeUsed")
    query = subprocess.run(
        ["squeue", f"--states={states}", "--noheader", "--name", run_id, "--Format", ",".join(f"{f}:|" for f in fields)],
        capture_output=True, text=True, env=env, check=True, timeout=60,
    )
    return [dict(zip(fields, (value.strip() for value in line.split("|")))) for line in query.stdout.splitlines()]


def seconds(time_used: str) -> int:
    """squeue's TimeUsed ([[days-]hours:]minutes:seconds) in seconds."""
    days, _, clock = time_used.rpartition("-")
    total = 0
    for part in clock.split(":"):
        total = 60 * total + int(part)
    return total + 86400 * int(days or 0)


class CancelOneJob(threading.Thread):
    """Cancels (scancel) the first job of ``rule`` seen running for CANCEL_AFTER_S seconds in the
    run whose log is being written to ``log_path``; ``cancelled`` is then its SLURM job id."""

    def __init__(self, log_path: Path, env: dict, rule: str):
        super().__init__(daemon=True)
        self.log_path, self.env, self.rule = log_path, env, rule
        self.cancelled: str | None = None
        self.finished = threading.Event()  # set by the test when the run has ended

    def run(self) -> None:
        run_id = None
        while not self.finished.is_set():
            time.sleep(0.5)
            if run_id is None:
                found = re.search(r"^SLURM run ID: (\S+)", self.log_path.read_text(errors="replace"), re.MULTILINE)
                run_id = found and found.group(1)
                continue
            for job in slurm_jobs(run_id, self.env, states="RUNNING"):
                if rule_of(job["Comment"]) == self.rule and seconds(job["TimeUsed"]) >= CANCEL_AFTER_S:
                    subprocess.run(["scancel", job["JobID"]], env=self.env, check=True, timeout=60)
                    self.cancelled = job["JobID"]
                    return


def rule_of(comment: str) -> str:
    """The rule in the plugin's job comment: rule_<rule> or rule_<rule>_wildcards_<values>."""
    assert comment.startswith("rule_"), comment
    return comment.removeprefix("rule_").split("_wildcards_")[0]


@pytest.mark.system
@pytest.mark.timeout(3600)
def test_quick_experiment_through_slurm_submits_every_job_retries_a_cancelled_one_and_gives_the_local_tables(
    slurm_cluster, quick_experiment, tmp_path_factory
):
    cluster, env = slurm_cluster
    # The workflow and the quick weight set in a folder of their own, the same configs as the local run.
    root = copy_workflow(tmp_path_factory.mktemp("wf-slurm"))
    shutil.copytree(quick_experiment.root / QUICK_WEIGHTS, root / QUICK_WEIGHTS)
    log_path = root / "snakemake-slurm.log"
    canceller = CancelOneJob(log_path, env, CANCELLED_RULE)
    with open(log_path, "w") as log_file:
        process = subprocess.Popen(
            [sys.executable, "-m", "snakemake", *SLURM_PROFILE, "--configfile", *EXPERIMENT_CONFIGS],
            cwd=root, env=env, stdout=log_file, stderr=subprocess.STDOUT, text=True,
        )
        canceller.start()
        try:
            returncode = process.wait(timeout=2400)
        finally:
            canceller.finished.set()
            if process.poll() is None:
                process.kill()
    canceller.join(timeout=60)
    log = log_path.read_text()
    assert returncode == 0, log[-6000:]
    assert canceller.cancelled is not None, f"no {CANCELLED_RULE} job ran for {CANCEL_AFTER_S} s to be cancelled"

    # Every job of the DAG but the target rule 'all' (no command) went through sbatch, once, and
    # the cancelled one a second time (Snakemake keeps a job's number when it retries it).
    expected = dag_job_counts(log)
    assert expected.pop("all") == 1
    assert re.findall(r"^localrule (\w+):", log, re.MULTILINE) == ["all"]
    submitted = re.findall(r"^Job (\d+) has been submitted with SLURM jobid (\d+)", log, re.MULTILINE)
    attempts = Counter(job for job, _ in submitted)
    assert len(attempts) == sum(expected.values()), submitted
    retried = [job for job, count in attempts.items() if count > 1]
    assert len(retried) == 1 and attempts[retried[0]] == 2, attempts
    retried_ids = [slurm_id for job, slurm_id in submitted if job == retried[0]]
    assert retried_ids[0] == canceller.cancelled, (retried_ids, canceller.cancelled)

    # SLURM's own records agree: the same jobs, all but the cancelled one completed, per rule as
    # many completed as the DAG has, each with the partition, GPU and memory profiles/slurm asks
    # for its rule (the retry with the second attempt's memory).
    run_id = re.search(r"^SLURM run ID: (\S+)", log, re.MULTILINE).group(1)
    jobs = slurm_jobs(run_id, env)
    assert {job["JobID"] for job in jobs} == {slurm_id for _, slurm_id in submitted}
    states = {job["JobID"]: job["State"] for job in jobs}
    assert states.pop(canceller.cancelled) == "CANCELLED"
    assert set(states.values()) == {"COMPLETED"}, [job for job in jobs if job["State"] != "COMPLETED"]
    completed = [job for job in jobs if job["JobID"] != canceller.cancelled]
    assert Counter(rule_of(job["Comment"]) for job in completed) == expected
    completions = [line for line in (cluster / "jobcomp.log").read_text().splitlines() if f" Name={run_id} " in line]
    assert len(completions) == len(submitted)
    assert sorted(re.search(r" JobState=(\S+) ", line).group(1) for line in completions) == ["CANCELLED"] + ["COMPLETED"] * len(completed)
    profile = yaml.safe_load((root / "profiles" / "slurm" / "config.yaml").read_text())
    threads = yaml.safe_load((root / "config" / "config.yaml").read_text())["threads"]
    assert set(threads.values()) == {1}  # every job asks for one CPU: its --threads
    for job in jobs:
        resources = {**profile["default-resources"], **profile["set-resources"].get(rule_of(job["Comment"]), {})}
        attempt = 2 if job["JobID"] == retried_ids[1] else 1
        assert job["Partition"] == resources["slurm_partition"], job
        assert job["tres-per-job"] == ("gres:gpu:1" if resources.get("gpu") else "N/A"), job
        assert job["MinMemory"] == f"{eval(resources['mem_mb'], {'attempt': attempt})}M", job
        assert job["NumCPUs"] == "1", job

    for number in range(1, 6):
        local = pd.read_csv(quick_experiment.root / "results" / "quick" / "tables" / f"table{number}.csv", comment="#")
        on_slurm = pd.read_csv(root / "results" / "quick" / "tables" / f"table{number}.csv", comment="#")
        pd.testing.assert_frame_equal(on_slurm, local, check_exact=True, obj=f"table{number}.csv")

