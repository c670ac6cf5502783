"""export: plain-NumPy policies and deployment (CPU MuJoCo, real robot). Not built yet (issue 5)."""
