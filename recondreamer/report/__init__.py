"""The paper's tables, figures and time summaries from the workflow's per-run outputs."""
