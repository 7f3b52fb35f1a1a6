"""generator/blender"""
