"""Fitting the artist controls of warp_hair to target images (losses, reparametrisation, the fitting loop).

Empty until the fitting issue lands; it depends on warp_hair, never the reverse.
"""
