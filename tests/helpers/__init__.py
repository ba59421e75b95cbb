"""Shared test code: independent NumPy references (reference_model, reference_bvh), sphere quadrature, the derivative
checks' common parts and the small scenes several test files render. Never imported by the product."""
