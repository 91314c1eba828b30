"""The validation toolkit every layer uses where input enters: argument converters
(:mod:`~qchain.checks.convert`), declared ranges (:mod:`~qchain.checks.bounds`), read-only
arrays (:mod:`~qchain.checks.frozen`), values shown in messages (:mod:`~qchain.checks.text`)
and network addresses (:mod:`~qchain.checks.addresses`). The exception classes are
:mod:`qchain.errors`'s. Nothing here imports the model."""
