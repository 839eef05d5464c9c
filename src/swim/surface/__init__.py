"""swim.surface"""
