"""flexlink: flexible-link robots from a TOML scene to an FMI 2.0 Co-Simulation FMU."""

__version__ = "0.1.0"
