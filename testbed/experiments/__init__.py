"""The experiments: the chapter's, the studies beyond it, and the critical-loss sweep."""
