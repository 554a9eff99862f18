"""Benchmarks: each module has ``main()`` printing its baseline, the ratios against it, and the seed."""
