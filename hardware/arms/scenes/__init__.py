"""MuJoCo scenes that include an arm file (generated; see hardware/arms/generate.py). A package so that the
XML files ship in the wheel (pyproject's package-data takes *.xml from package directories)."""
