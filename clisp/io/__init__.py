"""File input and output: our DNG-style raws, camera raws through rawpy, EXIF, and the image writers."""
