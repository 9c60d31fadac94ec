"""Baselines scored beside GPJA: optimal-step non-rigid ICP and meshes imported from other tools."""
