//! augsplat-report
