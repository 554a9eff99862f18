"""What the tests and the benchmarks share: loopback deployments, peers, clients, recordings.

A development package, not part of the product (it is not in the product's wheel): ``make``
installs it into ``.venv`` beside the product. Like the tests, it may reach inside a service.
"""
