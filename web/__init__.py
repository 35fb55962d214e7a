"""Static files of the status page, served by the daemon (no CDN: the rig may be offline)."""
