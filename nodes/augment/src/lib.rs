//! augsplat-augment
