"""swim.geometry"""
