"""Render one run along every evaluated trajectory: 'recondreamer render' once per trajectory, in
one process so that Python and torch start once per run instead of once per trajectory."""

import sys

from recondreamer.cli import main

with open(snakemake.log[0], "w") as log:  # noqa: F821 (snakemake is injected by Snakemake)
    sys.stderr = log
    for trajectory, out in zip(snakemake.params.trajectories, snakemake.output):  # noqa: F821
        argv = ["render", "--run", str(snakemake.params.run), "--scene", snakemake.input.scene,  # noqa: F821
                "--trajectory", trajectory, "--out", out, "--threads", str(snakemake.threads)]  # noqa: F821
        print("recondreamer " + " ".join(argv), file=log, flush=True)
        code = main(argv)
        if code != 0:
            sys.exit(code)
