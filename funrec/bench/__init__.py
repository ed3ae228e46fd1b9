"""Evaluation and benchmarking: metrics, baselines, the bench, its report, batch runs and the scheduler."""
