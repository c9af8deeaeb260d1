//! ONNX in and out of the policy format, for Python: the `policy import` / `policy export-onnx`
//! conversions of `dex-policy-tool`, on bytes.

use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::error::Error;

/// The `.dxpl` bytes of an ONNX model of an MLP policy (`policy import`): `task` (kebab-case) or,
/// when `None`, the layout file's or the model's metadata's; `layout`: the bytes of a policy file
/// whose layout to take instead of the Jaco cell's.
#[pyfunction]
#[pyo3(signature = (model, task=None, layout=None))]
pub fn onnx_to_policy<'py>(
    py: Python<'py>,
    model: &[u8],
    task: Option<&str>,
    layout: Option<&[u8]>,
) -> PyResult<Bound<'py, PyBytes>> {
    let task = task
        .map(|t| dex_policy::Task::from_name(t).ok_or_else(|| Error::UnknownTask(t.to_owned())))
        .transpose()?;
    let view = layout
        .map(dex_policy::PolicyView::decode)
        .transpose()
        .map_err(|e| Error::Onnx(e.into()))?;
    let settings = dex_policy_tool::ImportSettings {
        task,
        layout: view.as_ref(),
    };
    let imported = dex_policy_tool::import_onnx(model, &settings).map_err(Error::Onnx)?;
    Ok(PyBytes::new(py, &imported.file))
}

/// The ONNX model (bytes) of a policy file (`policy export-onnx`).
#[pyfunction]
pub fn policy_to_onnx<'py>(py: Python<'py>, policy: &[u8]) -> PyResult<Bound<'py, PyBytes>> {
    let onnx = dex_policy_tool::export_onnx(policy).map_err(Error::Onnx)?;
    Ok(PyBytes::new(py, &onnx))
}
