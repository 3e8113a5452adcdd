//! augsplat-field
