"""File formats in and out: atomic writes and JSON (files), meshes (meshio: OBJ, PLY, glTF/GLB),
glTF with morph targets and animation (gltf), MPEG-4 .fap files (fapfile), sound (audio). Readers
refuse damaged input with one-line errors; writers never leave partial files."""
