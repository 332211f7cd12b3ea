"""Shapes: upload a mesh with its mass (multipart), list, read, delete."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, Response, UploadFile, status
from starlette.concurrency import run_in_threadpool

from api.deps import ApiKeyDep, Limit, Offset, SettingsDep, StoreDep
from api.schemas import ShapePage, ShapeRead
from api.services import shapes

router = APIRouter(prefix="/api/v1/shapes", tags=["shapes"])


@router.post("", status_code=status.HTTP_201_CREATED, response_model=ShapeRead)
async def upload_shape(
    principal: ApiKeyDep,
    store: StoreDep,
    settings: SettingsDep,
    file: Annotated[UploadFile, File(description="An STL, OBJ or PLY mesh (metres unless scale).")],
    mass: Annotated[float, Form(gt=0, le=1e6, description="Mass of the body, kg.")],
    scale: Annotated[float, Form(gt=0, le=1e3, description="Factor to metres: 0.001 for mm.")] = 1.0,
    n_spheres: Annotated[int | None, Form(ge=1, le=500, description="Spheres of the clump.")] = None,
    name: Annotated[str | None, Form(max_length=200)] = None,
):
    """Validate the mesh, build its clump, store both; the report says what was repaired."""
    # Read one byte past the limit: enough to know it is too large without reading all of it.
    data = await file.read(settings.max_upload_bytes + 1)
    return await run_in_threadpool(
        shapes.upload_shape, store, settings, principal, filename=file.filename or "", data=data,
        mass=mass, scale=scale, n_spheres=n_spheres, name=name,
    )


@router.get("", response_model=ShapePage)
def list_shapes(
    principal: ApiKeyDep, store: StoreDep,
    limit: Limit = 50, offset: Offset = 0,
):
    return shapes.list_shapes(store, principal, limit, offset)


@router.get("/{shape_id}", response_model=ShapeRead)
def get_shape(shape_id: str, principal: ApiKeyDep, store: StoreDep):
    return shapes.get_shape(store, shape_id, principal)


@router.delete("/{shape_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response)
def delete_shape(shape_id: str, principal: ApiKeyDep, store: StoreDep, settings: SettingsDep):
    shapes.delete_shape(store, settings, shape_id, principal)
