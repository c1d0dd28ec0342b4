"""Programs that measure (bench, sweep, timing, nodes, encoder, sysid, multiarm, gradcheck, fingerprint); never
imported by the library."""
