"""Ground-truth cloth simulation (MuJoCo) for datasets. Filled by the simulation issue."""
