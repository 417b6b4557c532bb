"""Closed-loop evaluation: the `evaluate` config (`config`), one run of one controller over one window (`run`), the
planning and fan-out of all runs (`runner`) and the aggregation into reports/metrics.json (`aggregate`)."""
