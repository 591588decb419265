"""tissuebench: verification and benchmarking of reduced-order models of soft tissue."""

__version__ = "0.1.0"
