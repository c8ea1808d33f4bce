"""Visualisation: colour maps, point clouds, rig and candidate plots (files at the edges)."""
