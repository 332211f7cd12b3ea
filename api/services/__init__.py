"""Business logic below the routes: validation beyond the wire schema, status rules, summaries.

Services take the store and the caller's Principal and return wire models; they never see a
Request. Routes stay thin: validate, call one service function, return.
"""
