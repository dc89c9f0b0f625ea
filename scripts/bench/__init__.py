"""Benchmarks behind ``swarmslam bench ...``; each writes JSON and prints a table."""
