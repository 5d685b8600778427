"""The compiled co-simulation hot path; everything else about the package is in pyproject.toml.

``fmu_greybox._chainstep`` advances the corrector chain by one step, makes single-point
sparse-GP predictions (docs/greybox.md, "The chain step") and says why a step is refused. pip
compiles it at install with the machine's C compiler, from the numerical core ``chain_core.c``
and the rules of a step ``rules.c`` (which every native grey-box FMU compiles too, with the
same flags: ``native/cflags.txt``) and their CPython glue ``chainstep.c``.
"""

from pathlib import Path

from setuptools import Extension, setup

NATIVE = Path("fmu_greybox/native")

setup(
    ext_modules=[
        Extension(
            "fmu_greybox._chainstep",
            sources=[str(NATIVE / n) for n in ("chainstep.c", "chain_core.c", "rules.c")],
            depends=[str(NATIVE / n) for n in ("chain_core.h", "rules.h")],
            extra_compile_args=(NATIVE / "cflags.txt").read_text(encoding="ascii").split(),
        )
    ]
)
