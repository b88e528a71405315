//! Exports: the output size an export may reach, computed from the take
//! before anything is allocated.
