"""fmu-greybox: grey-box enhancement of white-box FMUs with sparse-GP correctors."""

__version__ = "0.1.0"
