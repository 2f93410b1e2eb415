//! Medical image and mesh files, converted to RAS millimetres.
