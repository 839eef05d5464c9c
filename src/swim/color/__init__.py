"""swim.color"""
