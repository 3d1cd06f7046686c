"""neuralcol.geometry"""
