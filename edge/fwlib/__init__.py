"""The FOCAS library host (`focas-edge fwlib-host`): FANUC's FOCAS library behind the packed surface.

The library is the user's copy from FANUC's FOCAS2 kit, loaded from the path they give; focas-edge never
ships it. What lives here, bottom up:

    structs     ctypes definitions of fwlib32.h's C structs
    library     load the library, declare the signatures the host calls
    calls       one packed request -> library calls on one handle -> the packed answer
    worker      one CNC: its own thread and handle, a timeout on every call, reconnect with backoff
    settings    the host's YAML file (library path, CNCs, where each is served)
    host        one packed endpoint per CNC, a worker behind each

Rules:

1. fwlib uses edge.focas only: the packed codecs (answers encoded exactly as the simulator encodes
   them), the packed endpoint (the same listener the simulator uses), the model and error types and the
   address parsers; plus the root ``edge.ConfigError``. Nothing above focas (config, collect, publish, service).
2. Library calls block, so they run on a worker's thread, never on the event loop.

This ``__init__`` imports nothing (the ctypes modules load only when the host starts); import each
submodule by its path.
"""

from __future__ import annotations

__all__ = ["calls", "host", "library", "settings", "structs", "worker"]
