"""The compiled co-simulation hot path; everything else about the package is in pyproject.toml.

``fmu_greybox._chainstep`` advances the corrector chain by one step and makes single-point
sparse-GP predictions (docs/greybox.md, "The chain step"). pip compiles it at install with the
machine's C compiler.
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "fmu_greybox._chainstep",
            sources=["fmu_greybox/native/chainstep.c"],
            extra_compile_args=["-O3", "-std=c11"],
        )
    ]
)
