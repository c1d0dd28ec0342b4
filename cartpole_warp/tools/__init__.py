"""Programs that measure (bench, sweep, timing); never imported by the library."""
