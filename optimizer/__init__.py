"""A calibration study's logic: parameter space, objectives, the GA (pymoo ask/tell), Pareto
ranking, the recommendation, and the driver that advances a study through an Executor and a Store.

Never imports RQ, Redis, SQLAlchemy or FastAPI: executors and stores are handed to it.
"""
