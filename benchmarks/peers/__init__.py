"""Peer implementations run beside ours in benchmarks (with labelled compatibility shims)."""
