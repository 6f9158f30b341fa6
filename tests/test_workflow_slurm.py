"""End to end on SLURM: the quick experiment (the same config as ``quick_experiment``) submitted job
by job with sbatch by snakemake-executor-plugin-slurm to a single-node cluster started on this
machine (.test/slurm/start.sh: Debian's slurm-wlm and munge), through profiles/slurm as written
plus .test/slurm/profile for that cluster. Every job of the DAG must go through sbatch, with the
partition, GPU and memory requests of profiles/slurm, and the five tables must equal those of the
local run to the last digit (same seeds, same single-threaded commands, nothing timed in them).
Minutes long, hence slow; it fails, never skips, when the cluster does not start or the run fails."""

import os
import re
import shutil
import socket
import subprocess
import sys
from collections import Counter

import pandas as pd
import pytest
import yaml

from workflow_fixtures import EXPERIMENT_CONFIGS, QUICK_WEIGHTS, REPO, copy_workflow

CLUSTER_SCRIPTS = REPO / ".test" / "slurm"
SLURM_PROFILE = ("--workflow-profile", "profiles/slurm", "--profile", ".test/slurm/profile")


def free_port_pair() -> int:
    """A port P such that P and P + 1 (slurmctld's and slurmd's) are free now, so that the test's
    cluster never collides with one already running (.test/slurm/start.sh defaults to 16817)."""
    for _ in range(20):
        with socket.socket() as first:
            first.bind(("", 0))
            port = first.getsockname()[1]
            with socket.socket() as second:
                try:
                    second.bind(("", port + 1))
                except OSError:
                    continue
        return port
    raise AssertionError("found no two consecutive free ports for slurmctld and slurmd")


@pytest.fixture(scope="module")
def slurm_cluster(tmp_path_factory):
    """The environment that points SLURM's commands at a running test cluster; stopped afterwards."""
    folder = tmp_path_factory.mktemp("slurm")
    # apt-get installs slurm-wlm and munge on a machine without them: minutes, not seconds.
    start = subprocess.run(
        ["bash", str(CLUSTER_SCRIPTS / "start.sh"), str(folder)],
        capture_output=True, text=True, timeout=900, env={**os.environ, "RECONDREAMER_SLURM_PORT": str(free_port_pair())},
    )
    try:
        assert start.returncode == 0, f"the test cluster did not start:\n{start.stdout}{start.stderr}"
        # bin/ holds an srun bound to this cluster's slurm.conf: the plugin's job step drops SLURM_CONF.
        yield folder, {**os.environ, "SLURM_CONF": str(folder / "slurm.conf"), "PATH": f"{folder / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    finally:
        stop = subprocess.run(["bash", str(CLUSTER_SCRIPTS / "stop.sh"), str(folder)], capture_output=True, text=True, timeout=300)
        assert stop.returncode == 0, f"the test cluster did not stop:\n{stop.stdout}{stop.stderr}"


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


def slurm_jobs(run_id: str, env: dict) -> list[dict]:
    """Every job SLURM holds for this run (finished ones stay for an hour: MinJobAge in start.sh)."""
    fields = ("JobID", "State", "Partition", "tres-per-job", "MinMemory", "NumCPUs", "Comment")
    query = subprocess.run(
        ["squeue", "--states=all", "--noheader", "--name", run_id, "--Format", ",".join(f"{f}:|" for f in fields)],
        capture_output=True, text=True, env=env, check=True, timeout=60,
    )
    return [dict(zip(fields, line.split("|"))) for line in query.stdout.splitlines()]


def rule_of(comment: str) -> str:
    """The rule in the plugin's job comment: rule_<rule> or rule_<rule>_wildcards_<values>."""
    assert comment.startswith("rule_"), comment
    return comment.removeprefix("rule_").split("_wildcards_")[0]


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_quick_experiment_through_slurm_submits_every_job_and_gives_the_local_tables(quick_experiment, slurm_cluster, tmp_path_factory):
    cluster, env = slurm_cluster
    # The workflow and the quick weight set in a folder of their own, the same configs as the local run.
    root = copy_workflow(tmp_path_factory.mktemp("wf-slurm"))
    shutil.copytree(quick_experiment.root / QUICK_WEIGHTS, root / QUICK_WEIGHTS)
    run = subprocess.run(
        [sys.executable, "-m", "snakemake", *SLURM_PROFILE, "--configfile", *EXPERIMENT_CONFIGS],
        cwd=root, env=env, capture_output=True, text=True, timeout=2400,
    )
    log = run.stdout + run.stderr
    assert run.returncode == 0, log[-6000:]

    # Every job of the DAG but the target rule 'all' (no command) went through sbatch, once.
    expected = dag_job_counts(log)
    assert expected.pop("all") == 1
    assert re.findall(r"^localrule (\w+):", log, re.MULTILINE) == ["all"]
    submitted = re.findall(r"^Job (\d+) has been submitted with SLURM jobid (\d+)", log, re.MULTILINE)
    assert len(submitted) == sum(expected.values()) == len({job for job, _ in submitted}), submitted

    # SLURM's own records agree: the same jobs, each completed in its first attempt, per rule as
    # many as the DAG has, each with the partition, GPU and memory profiles/slurm asks for its rule.
    run_id = re.search(r"^SLURM run ID: (\S+)", log, re.MULTILINE).group(1)
    jobs = slurm_jobs(run_id, env)
    assert {job["JobID"] for job in jobs} == {slurm_id for _, slurm_id in submitted}
    assert all(job["State"] == "COMPLETED" for job in jobs), [job for job in jobs if job["State"] != "COMPLETED"]
    assert Counter(rule_of(job["Comment"]) for job in jobs) == expected
    completions = [line for line in (cluster / "jobcomp.log").read_text().splitlines() if f" Name={run_id} " in line]
    assert len(completions) == len(submitted) and all(" JobState=COMPLETED " in line for line in completions)
    profile = yaml.safe_load((root / "profiles" / "slurm" / "config.yaml").read_text())
    threads = yaml.safe_load((root / "config" / "config.yaml").read_text())["threads"]
    assert set(threads.values()) == {1}  # every job asks for one CPU: its --threads
    for job in jobs:
        resources = {**profile["default-resources"], **profile["set-resources"].get(rule_of(job["Comment"]), {})}
        assert job["Partition"] == resources["slurm_partition"], job
        assert job["tres-per-job"] == ("gres:gpu:1" if resources.get("gpu") else "N/A"), job
        assert job["MinMemory"] == f"{eval(resources['mem_mb'], {'attempt': 1})}M", job
        assert job["NumCPUs"] == "1", job

    for number in range(1, 6):
        local = pd.read_csv(quick_experiment.root / "results" / "quick" / "tables" / f"table{number}.csv", comment="#")
        on_slurm = pd.read_csv(root / "results" / "quick" / "tables" / f"table{number}.csv", comment="#")
        pd.testing.assert_frame_equal(on_slurm, local, check_exact=True, obj=f"table{number}.csv")

