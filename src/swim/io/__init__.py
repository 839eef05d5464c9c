"""swim.io"""
