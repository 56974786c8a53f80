"""Grey-box diagnosis: fit a physics model, trace its held-out residual to a missing effect, add it, repeat.

data.py     Segment (one run of a log) + loading of plain .npz logs, held-out splits by run or segment
basis.py    rigid-body part: data-only trigonometric basis, or pinocchio's joint-torque regressor
effects.py  the library of declared effects (friction, periodic, backlash, drift, delay, coupling ...)
greybox.py  the linear grey-box model (rigid part + effects) and its regularised least-squares fit
trace.py    scoring every candidate effect on every joint against the residual
loop.py     the diagnose loop (fit, held-out error, trace, add, refit, stop)
report.py   report.json / report.md / evidence plots
"""
