"""neuralcol.collision"""
