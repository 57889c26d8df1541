"""Terminal views of a broker's traffic: `watch`, the demo's compact live view, and the `make run` demo itself."""
