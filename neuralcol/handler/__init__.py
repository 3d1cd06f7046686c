"""neuralcol.handler"""
