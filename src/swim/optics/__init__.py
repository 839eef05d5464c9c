"""swim.optics"""
