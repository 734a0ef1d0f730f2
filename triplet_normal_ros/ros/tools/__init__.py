"""Tooling around the node, not its runtime: the demo, a replay client, the node as a separate process and the
overload driver that the tests, the demo and docs/tools/ use to drive a running node."""
