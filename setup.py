"""Build of the optional native TCPROS receive loop; everything else is in pyproject.toml.

The extension is ``optional``: where no C compiler (or no Linux epoll) is available the
install still succeeds and the black box reads TCPROS in Python, saying so once at start.
"""

import sys

from setuptools import Extension, setup

native = [Extension("blackbox.sources.ros1._tcpros", ["src/blackbox/sources/ros1/_tcpros.c"],
                    optional=True, extra_compile_args=["-O2", "-std=c11", "-D_GNU_SOURCE"])]

setup(ext_modules=native if sys.platform.startswith("linux") else [])
