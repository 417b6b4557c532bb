"""The DVC stages' entry points (`python -m stages.<name>`).

Importing the package is the first thing such a process does, before the stage module imports torch, numpy, OpenCV
or numba: the moment to apply the numeric mode, whose switches those libraries read at import (stages/numerics.py).
Any other import of the package (tests, the dvc.yaml generator) leaves the process as it is.
"""

from stages.numerics import boot as _boot

_boot()
