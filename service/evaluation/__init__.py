"""Evaluation of detections against ground truth (metrics, data-set runners)."""
