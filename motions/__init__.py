"""Motion clips for the SMPL humanoid: format, importers, retargeting and the motion library."""
