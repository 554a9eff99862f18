"""The report of a run: ``report.md``, ``summary.json``, its figures and ``deadlines.json``."""
