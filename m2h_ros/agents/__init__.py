"""Controllers behind one interface: Move2Hear and the baselines."""
