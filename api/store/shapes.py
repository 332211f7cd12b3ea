"""Uploaded shapes in the SQL store."""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import undefer

from api.errors import NotFoundError
from api.models import ShapeRow
from api.store.base import ALL_OWNERS, Page, StoreBase


class ShapeStore(StoreBase):
    def add_shape(self, row: ShapeRow) -> str:
        with self.session() as s:
            s.add(row)
        return row.id

    def get_shape(
        self, shape_id: str, visible_to: str | None = ALL_OWNERS, with_data: bool = False
    ) -> ShapeRow:
        with self.session() as s:
            query = sa.select(ShapeRow).where(ShapeRow.id == shape_id)
            if with_data:
                query = query.options(undefer(ShapeRow.data))
            row = s.scalars(query).one_or_none()
            if row is None or not (visible_to is ALL_OWNERS or row.owner == visible_to):
                raise NotFoundError(f"no shape {shape_id!r}; list your shapes with GET /api/v1/shapes")
            return row

    def list_shapes(self, visible_to: str | None, limit: int, offset: int) -> Page:
        return self._newest_first(ShapeRow, visible_to, limit, offset)

    def delete_shape(self, shape_id: str) -> None:
        with self.session() as s:
            s.execute(sa.delete(ShapeRow).where(ShapeRow.id == shape_id))

