"""neuralcol.lit"""
