"""Simulator of MERIS L1b products with exact ground truth."""
