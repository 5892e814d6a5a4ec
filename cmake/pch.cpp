// The translation unit that compiles the precompiled headers (cmake/D3dTargets.cmake: d3d_pch).
