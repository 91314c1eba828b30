"""The recording service behind :mod:`qchain.logging`, cut by concern.

=====================  ==================================================================
module                 concern
=====================  ==================================================================
``records``            what travels: :class:`StepRecord`, :class:`RunInfo`, the row
                       layout, batches, errors, the checksummed metadata
``journal``            the simulating process's own copy of every record on disk (an
                       MCAP file beside the recording), and reading it while it grows
``scan``               reading MCAP records one by one, resynchronising after damage
``bounded``            reading files from anywhere within limits of time and memory
                       (:class:`ReadLimits`): regular files only, capped decompression,
                       record counts and nesting
``mcap_sink``          the recording: the mcap library's ``Writer``, qchain's JSON state
                       channel and the official Foxglove schemas (``foxglove-sdk``)
``rerun_sink``         the Rerun view: blueprint, camera, plots, served web viewer
``web_viewer``         the served web viewer's front: nothing but this machine is asked
``writer``             the writer (a process of its own, or a thread for a stream): it
                       reads the journal and feeds the sinks
``logger``             :class:`RunLogger`, the simulation's side
``reader``             reading a recording back (damage and gaps reported), recovering a
                       killed run's journal
``replay``             re-logging a recording into Rerun, ``qchain replay``
``options``            command-line flags, default paths, output path checks
``foxglove_layout``    the Foxglove layout qchain ships
=====================  ==================================================================

Nothing here imports the simulation: the writer process imports only this package (and
``qchain/__init__`` imports its heavy modules lazily).
"""
