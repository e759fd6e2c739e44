"""The base layer: the clock, geodesy, errors and the port conventions every other layer shares."""
