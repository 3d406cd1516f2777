"""The generic C half of every flexlink FMU (FMI glue, SS22 integrator), shipped as package data."""
