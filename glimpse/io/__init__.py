"""Small file I/O helpers (images, frame names) shared by the scene reader and the stages."""
