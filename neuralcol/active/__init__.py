"""neuralcol.active"""
