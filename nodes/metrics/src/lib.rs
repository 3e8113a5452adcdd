//! augsplat-metrics
