"""swim.rt"""
