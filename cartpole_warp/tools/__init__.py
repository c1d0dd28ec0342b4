"""Programs that measure (bench, sweep, timing, encoder, sysid, gradcheck); never imported by the library."""
