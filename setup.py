"""Only the optional compiled kernels live here; all metadata is in pyproject.toml."""
import sys

from setuptools import Extension, setup

# No FMA contraction: the kernels must round exactly like their pure-Python paths.
flags = [] if sys.platform == "win32" else ["-O2", "-ffp-contract=off"]
setup(ext_modules=[
    Extension("twin.fuzzy._kernel", ["twin/fuzzy/_kernel.c"], optional=True, extra_compile_args=flags),
    Extension("twin.plant._fastpath", ["twin/plant/_fastpath.c"], optional=True, extra_compile_args=flags),
    # the kernel reads its policy thresholds from a header generated from estimation/ekf_config.py
    Extension("estimation._ekf", ["estimation/_ekf.c"], depends=["estimation/_ekf_config.h"], optional=True,
              extra_compile_args=flags),
])
