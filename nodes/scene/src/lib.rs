//! augsplat-scene
