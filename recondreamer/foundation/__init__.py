"""The foundation: models trained once on the synthetic corpus and shipped as a weight set (``weights``), with their gates (``gates``)."""
