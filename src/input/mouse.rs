//! Mice as puppeteering tools (placeholder).
