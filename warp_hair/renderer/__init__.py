"""The path tracer and its derivatives with respect to the hair controls, in the order a newcomer reads them.

- render.py: `render`, the loop over pixels and their samples (pbrt's Render and EvaluatePixelSample) that the
  image and its Jacobian share.
- integrator.py: the path (`trace_path`, pbrt's Li) and next-event estimation over the lights (`sample_ld`).
- light_sampler.py: which light a vertex's shadow ray goes to (pbrt's LightSampler).
- prepare.py: a scene made ready on a device (BVH, camera, lights, card), built once for many renders.
- gradients.py: `render_jacobian`, the per-pixel ∂image/∂θ from one pass, and `render_grad`, its contraction with
  an adjoint (docs/gradients.md explains the estimator).
- camera.py, envmap.py: camera rays and the environment light.
"""
