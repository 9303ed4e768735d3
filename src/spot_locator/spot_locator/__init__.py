"""Sub-pixel lamp spot centres in both stereo images (gray centroid, ellipse fit,
circularity fusion, Wiener deblurring).
"""
