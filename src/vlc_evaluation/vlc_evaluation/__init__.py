"""Evaluation of the graph against ground truth, benchmarks and doc writers."""
