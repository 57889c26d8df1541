"""The running daemon and its surroundings: wiring, reload, sd_notify, the status HTTP endpoint and page, logging."""
