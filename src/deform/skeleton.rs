//! Shape-aware skeletal deformer (placeholder).
