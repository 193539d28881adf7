"""The models Jacobs et al. 2015 compare against, each as a NumPy reference and an OpenCL stage.

See `gazehdr.sim.models` for how a stage plugs into the simulator, and docs/baselines/ for what
each model does and where our reading of its paper fills a gap.
"""
