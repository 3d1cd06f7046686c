"""neuralcol.data"""
