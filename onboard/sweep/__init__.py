"""The sweep: its plan and progress (persisted so a restarted robot resumes) and its control.
"""
