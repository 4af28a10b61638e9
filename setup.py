"""Only the optional compiled kernel lives here; all metadata is in pyproject.toml."""
import sys

from setuptools import Extension, setup

# No FMA contraction: the kernel must round exactly like the pure-Python path.
flags = [] if sys.platform == "win32" else ["-O2", "-ffp-contract=off"]
setup(ext_modules=[Extension("twin.fuzzy._kernel", ["twin/fuzzy/_kernel.c"], optional=True, extra_compile_args=flags)])
