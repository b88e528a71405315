//! lp-FFD grid deformer (placeholder).
