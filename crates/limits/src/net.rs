//! The network edge: connections per address and in all, and how long a
//! connection may take to send its headers or stay silent.
