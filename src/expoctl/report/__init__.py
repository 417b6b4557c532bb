"""The evaluation report: reports/results.md (`results`) and its figures (`figures`)."""
