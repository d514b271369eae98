//! The controller's YAML as the parameter store, optionally also set live on the running
//! controller (its wheel multipliers through the parameter services).

use super::*;

#[async_trait]
impl ParamStore for RosStore {
    fn info(&self) -> ComponentInfo {
        let mut info = self.yaml.info();
        info.details["set_live"] = json!(self.set_live);
        info
    }

    async fn read(&self) -> Result<WheelParams, BaseError> {
        self.yaml.read().await
    }

    async fn write(&self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        self.yaml.write(params).await
    }

    async fn commit(&self) -> Result<(), BaseError> {
        // The multipliers the file will hold after this commit.
        let staged = self.yaml.read().await?;
        self.yaml.commit().await?;
        if self.set_live {
            let cfg = self.yaml.on_disk()?;
            let m = cfg.multipliers_for(&staged);
            let values = [
                m.wheel_separation_multiplier,
                m.left_wheel_radius_multiplier,
                m.right_wheel_radius_multiplier,
            ];
            let service = self.service("set_parameters");
            let refused = self
                .set_multipliers(&service, values)
                .await
                .map_err(|e| BaseError::backend("store (live)", e))?;
            if !refused.is_empty() {
                // Not `Refused`: the file was replaced already, so the commit happened and a
                // rollback must put the file back too.
                return Err(BaseError::backend(
                    "store (live)",
                    std::io::Error::other(format!(
                        "the file was written, but the running controller refused {service}: {}",
                        refused.join("; ")
                    )),
                ));
            }
            *self.running.write().unwrap_or_else(|p| p.into_inner()) = staged;
        }
        Ok(())
    }

    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        self.yaml.read_committed().await
    }

    fn resolution(&self) -> WheelParams {
        self.yaml.resolution()
    }

    fn file(&self) -> Option<std::path::PathBuf> {
        self.yaml.file()
    }

    async fn check_write(&self, params: &WheelParams) -> Result<(), BaseError> {
        self.yaml.check_write(params).await?;
        if self.set_live {
            self.check_live().await?;
        }
        Ok(())
    }
}

impl RosStore {
    /// `/<controller>/<name>`, one of the controller node's services.
    pub(super) fn service(&self, name: &str) -> String {
        format!("/{}/{name}", self.controller)
    }

    /// Calls the controller's `set_parameters` with the three multipliers (in
    /// [`MULTIPLIER_KEYS`] order); the reasons of those it refused.
    pub(super) async fn set_multipliers(
        &self,
        service: &str,
        values: [f64; 3],
    ) -> Result<Vec<String>, RosbridgeError> {
        let parameters: Vec<Value> = MULTIPLIER_KEYS
            .iter()
            .zip(values)
            .map(|(name, v)| json!({"name": name, "value": {"type": 3, "double_value": v}}))
            .collect();
        let answer = self
            .client
            .call_service(
                service,
                "rcl_interfaces/srv/SetParameters",
                json!({ "parameters": parameters }),
                Duration::from_secs(3),
            )
            .await?;
        let results = answer.get("results").and_then(Value::as_array);
        Ok(match results {
            Some(r) if r.len() == MULTIPLIER_KEYS.len() => MULTIPLIER_KEYS
                .iter()
                .zip(r)
                .filter(|(_, x)| x.get("successful").and_then(Value::as_bool) != Some(true))
                .map(|(name, x)| {
                    let why = x.get("reason").and_then(Value::as_str).unwrap_or("");
                    format!("{name}: {}", if why.is_empty() { "refused" } else { why })
                })
                .collect(),
            _ => vec![format!(
                "the answer has no result for each of the three parameters: {answer}"
            )],
        })
    }

    /// Proves, before the robot moves, that the running controller can take the multipliers
    /// live: its `get_parameters` answers with a double for each, its `describe_parameters`
    /// says each is a double and not read-only, and its `set_parameters` accepts each at the
    /// value it has now (a write that changes nothing, so that a parameter callback that
    /// refuses sets, or a node that answers no sets, is found before the robot moves).
    pub(super) async fn check_live(&self) -> Result<(), BaseError> {
        let unwritable = |why: String| BaseError::Unwritable {
            component: "store (live)".into(),
            source: format!("--ros-set-live: {why}").into(),
        };
        let call = |service: String, kind: &'static str, args: Value| async move {
            self.client
                .call_service(&service, kind, args, Duration::from_secs(3))
                .await
                .map_err(|e| {
                    unwritable(format!(
                        "{service} failed ({e}); is the controller running under that name?"
                    ))
                })
        };
        let names = json!({ "names": MULTIPLIER_KEYS });
        let service = self.service("get_parameters");
        let answer = call(
            service.clone(),
            "rcl_interfaces/srv/GetParameters",
            names.clone(),
        )
        .await?;
        let list = |answer: &Value, field: &str| {
            answer
                .get(field)
                .and_then(Value::as_array)
                .cloned()
                .unwrap_or_default()
        };
        let values = list(&answer, "values");
        let now: Vec<f64> = values
            .iter()
            .filter(|v| v.get("type").and_then(Value::as_u64) == Some(3))
            .filter_map(|v| v.get("double_value").and_then(Value::as_f64))
            .collect();
        let Ok(now) = <[f64; 3]>::try_from(now) else {
            return Err(unwritable(format!(
                "the running controller does not declare {} as doubles with a value ({service} \
                 gave {} value(s)): a controller without them cannot take a calibration live",
                MULTIPLIER_KEYS.join(", "),
                values.len()
            )));
        };
        let service = self.service("describe_parameters");
        let answer = call(
            service.clone(),
            "rcl_interfaces/srv/DescribeParameters",
            names,
        )
        .await?;
        let descriptors = list(&answer, "descriptors");
        for name in MULTIPLIER_KEYS {
            let Some(d) = descriptors
                .iter()
                .find(|d| d.get("name").and_then(Value::as_str) == Some(name))
            else {
                return Err(unwritable(format!("{service} does not describe {name}")));
            };
            if d.get("read_only").and_then(Value::as_bool) != Some(false) {
                return Err(unwritable(format!(
                    "{service} says {name} is read-only: the running controller cannot take it \
                     live (without --ros-set-live the YAML is written, and the controller reads \
                     it when it is restarted)"
                )));
            }
            if d.get("type").and_then(Value::as_u64) != Some(3) {
                return Err(unwritable(format!(
                    "{service} says {name} is of type {}, not a double (3)",
                    d.get("type").unwrap_or(&Value::Null)
                )));
            }
        }
        let service = self.service("set_parameters");
        let refused = self
            .set_multipliers(&service, now)
            .await
            .map_err(|e| unwritable(format!("{service} failed ({e})")))?;
        if !refused.is_empty() {
            return Err(unwritable(format!(
                "{service} refused the multipliers at the values they have now ({}): it would \
                 refuse the calibration too",
                refused.join("; ")
            )));
        }
        Ok(())
    }
}
