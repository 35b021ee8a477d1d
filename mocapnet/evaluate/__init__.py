"""Scoring: metrics, the evaluation harness and reports."""
