"""One APIRouter per resource; handlers validate, call one service function and return a model."""
