"""The path tracer and its derivatives with respect to the hair controls.

- prepare.py: a scene made ready on a device (BVH, camera, lights, card), built once for many renders.
- forward.py: `render`, and the pixel kernel that the forward and gradient passes share.
- jacobian.py: `render_jacobian`, the per-pixel ∂image/∂θ from one pass; gradients.py: `render_grad`, its
  contraction with an adjoint (docs/gradients.md explains the estimator).
- integrator.py: the path (`trace_path`, pbrt's Li) and next-event estimation over the lights (`sample_ld`).
- camera.py, envmap.py: camera rays and the environment light.
"""
