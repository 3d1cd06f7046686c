"""neuralcol.utils"""
