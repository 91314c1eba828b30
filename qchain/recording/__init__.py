"""The recording service behind :mod:`qchain.logging`, one module a concern (docs/recording.md,
"How it is built").

Nothing here imports the simulation: the writer process imports only this package (and
``qchain/__init__`` imports its heavy modules lazily)."""
