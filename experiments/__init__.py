"""Experiments: studies too slow for the test suite, one entry point per module.

Run each from the repository root as ``python -m experiments.NAME [--help]`` (or as
``python experiments/NAME.py``); what several of them share lives in ``experiments.common``.
experiments/README.md describes each study and its recorded results.
"""
