"""The run's configuration (``run_config.yaml``) as an HTML page for the Snakemake report, which
shows HTML pages and images but offers a YAML file only as a download."""

from __future__ import annotations

import html
from pathlib import Path

from recondreamer.errors import RecondreamerError
from recondreamer.io import write_text_atomic


def config_page(config_yaml: str | Path, out: str | Path) -> Path:
    """Write ``out``: the YAML text, escaped, in a ``<pre>`` block, as the workflow wrote it."""
    config_yaml, out = Path(config_yaml), Path(out)
    try:
        text = config_yaml.read_text()
    except OSError as error:
        raise RecondreamerError(f"{config_yaml}: cannot read the run's configuration ({error})") from None
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Configuration of this run</title>
<style>body {{ font-family: sans-serif; margin: 1em; }} pre {{ font-size: 0.85em; }}</style></head>
<body>
<h2>Configuration of this run</h2>
<p>The workflow config as this run used it (config/config.yaml with the --configfile files layered
over it), from <code>{html.escape(str(config_yaml))}</code>; config/README.md explains each key.</p>
<pre>{html.escape(text)}</pre>
</body></html>
"""
    write_text_atomic(out, page)
    return out
