"""The camera type every stage shares (OpenCV pinhole, world-to-camera; model.py), its conversions,
similarity alignment (align.py), lens undistortion (undistort.py) and orbit cameras around a person
(orbit.py)."""
