"""The benchmarks: each module runs from the repository root as `python -m bench.NAME [--quick]`.

bench/harness.py is the one place a result gets its machine, commit, date and shape; results/ holds the
published results (results/README.md lists them), bench/out/ the scratch output of a run (git-ignored).
"""
