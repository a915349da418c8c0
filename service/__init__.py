"""Online side: relighting incoming frames with a loaded reflectance bundle."""
