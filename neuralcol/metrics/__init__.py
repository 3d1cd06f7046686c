"""neuralcol.metrics"""
