"""The compiled co-simulation hot path; everything else about the package is in pyproject.toml.

``fmu_greybox._chainstep`` advances the corrector chain by one step and makes single-point
sparse-GP predictions (docs/greybox.md, "The chain step"). pip compiles it at install with the
machine's C compiler, from the numerical core ``chain_core.c`` (which every native grey-box FMU
compiles too, with the same flags: ``native/cflags.txt``) and its CPython glue ``chainstep.c``.
"""

from pathlib import Path

from setuptools import Extension, setup

NATIVE = Path("fmu_greybox/native")

setup(
    ext_modules=[
        Extension(
            "fmu_greybox._chainstep",
            sources=[str(NATIVE / "chainstep.c"), str(NATIVE / "chain_core.c")],
            depends=[str(NATIVE / "chain_core.h")],
            extra_compile_args=(NATIVE / "cflags.txt").read_text(encoding="ascii").split(),
        )
    ]
)
