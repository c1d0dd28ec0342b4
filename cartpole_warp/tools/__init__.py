"""Programs that measure (bench, sweep, timing, nodes, encoder, sysid, multiarm, gradcheck); never imported by the
library."""
