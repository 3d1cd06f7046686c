"""neuralcol.nn"""
