"""The raster half's numpy side: G-buffer statistics, shadow maps, draw chunks, the numpy reference raster."""
